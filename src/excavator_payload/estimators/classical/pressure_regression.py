r"""Inverse dynamics on the machine sensor set: weighing from cylinder pressures and IMUs.

The kernel behind ``inverse-dynamics`` when the data hold the machine sensor set (issue 12,
first step). Per sample it regresses, as on the thesis set, the payload on the arm torques,

.. math:: \tau_j - \tau_{0,j}(q, \dot q, \ddot q, \text{tilt}) = m\,\varphi_j(q, \dot q, \ddot q,
          \text{tilt}) + \varepsilon_j, \qquad j \in \{\text{boom, dipper, bucket}\},

with the torques from the pressures, :math:`\tau_j = \text{count}_j\,\partial l_j/\partial q_j\,
(p_h A_h - p_r A_r - F_f)`, all from ``HydraulicSymbolic.functions["pressure_regression"]``
(the single symbolic source, compiled). What the machine does not measure is derived:

* **accelerations** (of boom, dipper, bucket and slew) by a *centred* smoothing differentiator
  of the measured rates: the least-squares slope over ``2·half_window + 1`` samples. Centred,
  it has no lag (a causal filtered derivative lags and biases the inertial torques); the price
  is that the estimate refers to the sample ``half_window + 2`` samples back (50 ms by
  default; the two more are the outlier test's look-ahead);
* **ground tilt** from the house IMU: at slew angle 0 the house's pitch and roll are those of
  the ground frame (:func:`ground_tilt`); the slew angle itself does not enter the dynamics
  (only its rate and acceleration do);
* **seal friction**: its presliding state is unknown, so the model's friction uses a smooth
  sign of the rod speed (±1 once the rod moves faster than a tenth of the Stribeck velocity),
  and its load-dependent part is of the *load* force, recovered from the measured piston force
  by one fixed-point step (``HydraulicSymbolic``'s ``moving_friction``); near standstill the
  friction can be anything within ± the breakaway force, so that joint's residual variance
  grows by (breakaway torque)²/3, fading with speed (down-weighted, not skipped).

Weights: each joint's residual variance is the pressure noise (and pump ripple) through
:math:`\text{count}\,\partial l/\partial q\,(A_h, A_r)` plus the friction term above; the
estimate is :math:`\hat m = \sum \varphi^\top W r / \sum \varphi^\top W \varphi`, recursively.
Sensor offsets (zero drift) are *not* estimated here: that is the calibration and zero of issue 12.

Outlier gate
------------
A glitched frame (a bit error, a transmitter's spike) is one sample off the signal while its
neighbours agree. The kernel regresses a sample only ``half_window`` samples after it
arrives, so it can afford to look two samples ahead. Sample :math:`k` *stands out* when some
signal :math:`i` jumps away from both neighbours in the same direction,

.. math:: (x_k - x_{k-1})(x_k - x_{k+1}) > 0, \quad
          \min(|x_k - x_{k-1}|, |x_k - x_{k+1}|) > z\,\sigma_{\Delta,i},
          \quad
          \min(|x_k - x_{k-1}|, |x_k - x_{k+1}|) > |x_{k+1} - x_{k-1}|;

such a sample is never regressed (its slot is filled by the mean of its neighbours: the
differentiator needs evenly spaced samples). It is a *glitch*, reported ``rejected_outlier``,
when that signal also stands off, in the same direction and by more than
:math:`z\,\sigma_{\Delta,i}`, the straight line through each side's two samples,

.. math:: (x_k - \hat x_k^{\pm})(x_k - x_{k-1}) > 0, \quad |x_k - \hat x_k^{\pm}| >
          z\,\sigma_{\Delta,i}, \qquad \hat x_k^- = 2x_{k-1} - x_{k-2}, \;
          \hat x_k^+ = 2x_{k+1} - x_{k+2},

with :math:`\sigma_{\Delta,i}` the robust spread of the signal's sample-to-sample changes on
the fitting data (:func:`difference_scale`) and :math:`z` the two-sided normal quantile of the
gate's probability (``GATE_PROBABILITY``). A step (a valve opening) moves away from one
neighbour only and a ramp from both in opposite directions: neither stands out. The sharp
corner of a pressure (a rod stopping, a chamber's force turning) stands out but lies on the
line through one side's samples: it is not regressed — the rigid-body model explains such
instants worst — and not reported either, for it is no fault of a sensor. A model-based χ²
test of the arriving sample did not work here: the rigid-body residual of a transient runs
tens of noise deviations for a quarter of a second, which rejected good data and
re-initialised the estimate. The third condition asks the sample to stand out from both
neighbours more than they differ from each other: without it a glitch in the *next* frame
made a good sample in fast motion look like a spike, and the "repair" averaged the glitch
into the slot. Not caught: two or more bad frames in a row that agree with each other (the
plausibility limits still bound them).
"""

from __future__ import annotations

import math
from collections import deque
from typing import Mapping

import numpy as np

from excavator_payload.data.dataset import Dataset
from excavator_payload.data.schema import MACHINE_SENSORS
from excavator_payload.errors import EstimatorError
from excavator_payload.estimators.classical.kernels import PayloadKernel
from excavator_payload.estimators.classical.machine_calibration.settings import DEFAULT_PRESSURE_STD
from excavator_payload.estimators.status import Status, StepResult
from excavator_payload.model.hydraulic import HydraulicArmModel, compiled_function
from excavator_payload.platforms import HYDRAULIC

SIGNALS = MACHINE_SENSORS.signals
ANGLES = [SIGNALS.index(s) for s in ("boom_angle", "dipper_angle", "bucket_angle")]
RATES = [SIGNALS.index(s) for s in ("boom_rate", "dipper_rate", "bucket_rate", "slew_rate")]
PITCH, ROLL = SIGNALS.index("house_pitch"), SIGNALS.index("house_roll")
PRESSURES = [SIGNALS.index(s) for s in SIGNALS if s.endswith("_pressure")]


def white_noise_variance(x: np.ndarray) -> float | None:
    """White-noise variance of the columns of ``x`` from their second differences:
    var(Δ²x) = 6σ² for white noise on a smooth signal, through the median of χ²₁ (0.4549), which
    makes it robust to jumps; None with fewer than 10 finite rows.

    Parameters
    ----------
    x : numpy.ndarray
        Samples (rows) of one or more signals (columns), evenly spaced.
    """
    d2 = np.diff(x, 2, axis=0)
    d2 = d2[np.all(np.isfinite(d2), axis=1)]
    if len(d2) < 10:
        return None
    return float(np.median(d2**2) / 0.4549 / 6)


def pressure_noise_from_data(dataset: Dataset) -> float:
    """White noise of the pressure transmitters (Pa) from second differences of the measured
    pressures (:func:`white_noise_variance`): needs no known payload, so any data will do; it
    sees the white noise and the aliased pump ripple, as the estimator does.

    Parameters
    ----------
    dataset : Dataset
        Machine-sensor-set data.

    Returns
    -------
    float
        Standard deviation, Pa.
    """
    variance = white_noise_variance(dataset.frame[[SIGNALS[i] for i in PRESSURES]].to_numpy(float))
    return DEFAULT_PRESSURE_STD if variance is None else math.sqrt(variance)


#: Samples after the one the outlier test judges: two, so that it sees two neighbours each side.
LOOK_AHEAD = 2


def ground_tilt(house_pitch: float, house_roll: float) -> tuple[float, float]:
    """Ground [pitch, roll] that gives the house this inclination at slew angle 0.

    Inverse of ``HydraulicArmModel.house_inclination`` at ψ = 0: the house's z row is
    (cos r sin p, sin r, cos r cos p), so roll = r and sin(pitch_house) = cos r sin p.

    Parameters
    ----------
    house_pitch, house_roll : float
        House inclination, rad.

    Returns
    -------
    tuple of float
        Ground ``(pitch, roll)``, rad.
    """
    roll = house_roll
    ratio = math.sin(house_pitch) / max(math.cos(roll), 1e-9)
    return math.asin(min(1.0, max(-1.0, ratio))), roll


class PressureRegression:
    """Streaming payload regression on machine-sensor-set samples (see the module doc).

    Parameters
    ----------
    arm : HydraulicArmModel
        The machine the estimator believes in.
    pressure_std : float
        White noise of one pressure transmitter, Pa.
    ripple_fraction : float
        Residual pump ripple as a share of the pressure (its RMS enters the weights).
    half_window : int
        Samples each side of the centred differentiator.
    forgetting : float
        Forgetting factor λ of the recursive sums.
    """

    # What the per-sample regression cannot do, said explicitly (the calibrated kernel,
    # machine_calibration.kernel.CalibratedKernel, does these): it is ready from the first
    # sample, detects no new load, checks no joint against the others and carries no model error.
    ready = True
    steady = True
    changing = False
    checks_joints = False
    #: whether the joint check runs (set per sample by the kernel); the C export has no check
    joint_check = False
    joint_checked = True
    joint_fault = ""
    joint_degraded = (math.nan, 0.0)
    joint_pausing = False
    joint_suspect = False
    joint_moved_settled = False
    new_loads = 0
    model_std = 0.0

    def __init__(self, arm: HydraulicArmModel, pressure_std: float, ripple_fraction: float = 0.0,
                 half_window: int = 5, forgetting: float = 1.0):
        self.arm = arm
        self._f = compiled_function("pressure_regression")
        self._p = arm.p
        cyl = arm.machine.cylinders
        self._head = np.array([c.head_area for c in cyl])
        self._rod = np.array([c.rod_area for c in cyl])
        self._v_stribeck = np.array([c.stribeck_velocity for c in cyl])
        self.pressure_var = float(pressure_std) ** 2 + 1.0  # 1 Pa² floor keeps weights finite
        self.ripple_var_share = float(ripple_fraction) ** 2 / 2  # RMS² of a sine of that amplitude
        self.half_window = int(half_window)
        self.forgetting = float(forgetting)
        self.spike_threshold = np.full(len(SIGNALS), np.inf)  # set from data by the estimator
        self.judge = True  # the one-frame outlier test (Estimator.gating)
        self.rejected = False
        self.reset()

    def reset(self) -> None:
        """Start again: empty the differentiator's window and zero the recursive sums."""
        # the differentiator's window and the newest samples, not yet judged
        self._buffer: deque = deque(maxlen=2 * self.half_window + 1 + LOOK_AHEAD)
        self.num = 0.0
        self.info = 0.0

    def restart_window(self) -> None:
        """Forget the differentiator's window but keep the sums (after a gap in the data)."""
        self._buffer.clear()

    @staticmethod
    def _slope(times, rates) -> np.ndarray:
        """Least-squares slope of the rates over a window, rad/s²."""
        t = np.asarray(times, float)
        t = t - t.mean()
        rates = np.asarray(rates, float)
        return (t @ (rates - rates.mean(axis=0))) / (t @ t)

    def _evaluate(self, sample: np.ndarray, qdd: np.ndarray):
        """Kernel outputs (residual, φ, lever, rod speed, stiction) and residual variance."""
        q = np.zeros(4)
        q[:3] = sample[ANGLES]
        tilt = ground_tilt(sample[PITCH], sample[ROLL])
        pressures = sample[PRESSURES]
        out = self._f(q, sample[RATES], qdd, np.array(tilt), pressures, self._p)
        residual, phi, lever, speed, stiction = (np.asarray(o).ravel() for o in out)
        p_head, p_rod = pressures[0::2], pressures[1::2]
        side_var = self.pressure_var + self.ripple_var_share * np.stack([p_head, p_rod]) ** 2
        var = lever**2 * (self._head**2 * side_var[0] + self._rod**2 * side_var[1])
        still = np.exp(-(speed / (3 * self._v_stribeck)) ** 2)
        return residual, phi, var + still * stiction**2 / 3

    def _spike(self, context) -> tuple[bool, bool]:
        """Whether the middle of five consecutive samples stands out, and whether it is a
        one-frame glitch (:func:`judge_frame`)."""
        before2, before, sample, after, after2 = context
        return judge_frame(before, sample, after, self.spike_threshold, before2, after2)

    def update(self, time: float, values: np.ndarray) -> bool:
        """Consume one sample; returns whether a sample (the centre of the window) was used.
        :attr:`rejected` says whether the sample two before this one was judged a glitch; the
        window regressed ends on that sample (every sample in it has been judged).

        Parameters
        ----------
        time : float
            Sample time, s.
        values : numpy.ndarray
            The sample, in machine-set :data:`SIGNALS` order (SI units).

        Returns
        -------
        bool
            Whether a sample was used.
        """
        self._buffer.append((time, values, True))
        self.rejected = False
        if self.judge and len(self._buffer) >= 4:  # the first sample has no neighbour before it
            context = [self._buffer[i][1] if len(self._buffer) >= -i else None for i in range(-5, 0)]
            stands_out, self.rejected = self._spike(context)
            if stands_out:
                t_mid = self._buffer[-3][0]
                self._buffer[-3] = (t_mid, 0.5 * (context[1] + context[3]), False)
        if len(self._buffer) < self._buffer.maxlen:
            return False
        _, centre, centre_used = self._buffer[self.half_window]
        if not centre_used:
            return False
        window = list(self._buffer)[:-LOOK_AHEAD]
        qdd = self._slope([b[0] for b in window], [b[1][RATES] for b in window])
        residual, phi, var = self._evaluate(centre, qdd)
        w = 1.0 / var
        self.num = self.forgetting * self.num + float(np.sum(w * phi * residual))
        self.info = self.forgetting * self.info + float(np.sum(w * phi * phi))
        return True

    @property
    def estimate(self) -> float:
        return self.num / self.info if self.info > 0 else math.nan

    @property
    def weighed_info(self) -> float:
        """The information on the payload its σ reads (the sums' I here)."""
        return self.info


def judge_frame(before: np.ndarray, sample: np.ndarray, after: np.ndarray, threshold: np.ndarray,
                before2: np.ndarray | None = None, after2: np.ndarray | None = None) -> tuple[bool, bool]:
    """Whether ``sample`` stands out between its neighbours, and whether it is a one-frame glitch.

    It *stands out* where some signal moves away from both neighbours, in the same direction,
    by more than its ``threshold`` (:func:`spike_threshold`) and more than the neighbours differ
    from each other: such a sample is never regressed. It is a *glitch* where that signal also
    stands off, in that direction and by more than the threshold, the straight line through
    each side's two samples (where the second neighbours are given): the corner of a
    piecewise-linear signal lies on one of them, so a sharp turn of a pressure is not reported
    (module doc). Used by the pressure kernels.

    Parameters
    ----------
    before, sample, after : numpy.ndarray
        The sample judged and its neighbours, one value per signal.
    threshold : numpy.ndarray
        Per-signal threshold z·σ_Δ.
    before2, after2 : numpy.ndarray or None
        The samples before ``before`` and after ``after``; ``None`` where not (yet) known.

    Returns
    -------
    tuple of bool
        ``(stands_out, glitch)``; a glitch always stands out.
    """
    d1 = sample - before
    if not (np.abs(d1) > threshold).any():  # the usual case, in three operations
        return False, False
    d2 = sample - after
    smaller = np.minimum(np.abs(d1), np.abs(d2))
    out = (d1 * d2 > 0) & (smaller > threshold) & (smaller > np.abs(after - before))
    if not out.any():
        return False, False
    glitch = out
    for near, far in ((before, before2), (after, after2)):
        if far is not None:
            off_line = sample - (2 * near - far)
            glitch = glitch & (off_line * d1 > 0) & (np.abs(off_line) > threshold)
    return True, bool(glitch.any())


def one_frame_glitch(before: np.ndarray, sample: np.ndarray, after: np.ndarray, threshold: np.ndarray,
                     before2: np.ndarray | None = None, after2: np.ndarray | None = None) -> bool:
    """Whether ``sample`` is a one-frame glitch (:func:`judge_frame`'s second answer).

    Parameters
    ----------
    before, sample, after : numpy.ndarray
        The sample judged and its neighbours, one value per signal.
    threshold : numpy.ndarray
        Per-signal threshold z·σ_Δ.
    before2, after2 : numpy.ndarray or None
        The samples before ``before`` and after ``after``; ``None`` where not known.
    """
    return judge_frame(before, sample, after, threshold, before2, after2)[1]


def difference_scale(dataset) -> np.ndarray:
    """Spread of each machine-set signal's sample-to-sample change (within experiments), as
    the std of a Gaussian with the same 99th percentile of the absolute change.

    Parameters
    ----------
    dataset : Dataset
        Machine-sensor-set data.

    Returns
    -------
    numpy.ndarray
        One scale per signal (its SI unit); infinite with fewer than 100 changes.
    """
    f = dataset.frame
    x = f[list(SIGNALS)].to_numpy(float)
    exp = f["experiment"].to_numpy()
    d = np.diff(x, axis=0)[exp[1:] == exp[:-1]]
    d = d[np.all(np.isfinite(d), axis=1)]
    if len(d) < 100:
        return np.full(len(SIGNALS), np.inf)  # too little data to judge: no gate
    # the 99th percentile, read as a Gaussian's (2.576 σ): sample-to-sample changes are not
    # Gaussian — motion and the IMUs' acceleration leak widen their tails, and a median-based
    # scale flagged good angle samples at hydraulic transients (8 in 20 000 on NMPC swings)
    return np.maximum(np.quantile(np.abs(d), 0.99, axis=0) / 2.576, 1e-12)


def spike_threshold(scale: np.ndarray) -> np.ndarray:
    """Per-signal threshold z·σ_Δ of the one-frame outlier test (module doc).

    Parameters
    ----------
    scale : numpy.ndarray
        Per-signal scale σ_Δ from :func:`difference_scale`.

    Returns
    -------
    numpy.ndarray
        Thresholds, same units.
    """
    from scipy.stats import norm

    from excavator_payload.estimators.checks import GATE_PROBABILITY

    return norm.isf(GATE_PROBABILITY / 2) * np.asarray(scale, float)


def restore_difference_scale(arrays: Mapping[str, np.ndarray]) -> np.ndarray:
    """The machine set's per-signal outlier-test scale from a saved model (checked).

    Parameters
    ----------
    arrays : Mapping[str, numpy.ndarray]
        The saved model's arrays.

    Returns
    -------
    numpy.ndarray
        The 15 per-signal scales (SI units of each signal).
    """
    if "difference_scale" not in arrays:
        raise EstimatorError("saved model predates the machine set's outlier test: fit it again")
    scale = np.asarray(arrays["difference_scale"], float)
    if scale.shape != (15,) or np.any(np.isnan(scale)) or np.any(scale <= 0):
        raise EstimatorError("saved outlier-test scale is corrupt")
    return scale


class PressureKernel(PayloadKernel):
    """The machine sensor set's kernel of ``inverse-dynamics``: a :class:`PressureRegression`
    (or, held by ``calibrated``, its calibrated form) and the statuses it reports.

    Parameters
    ----------
    regression : PressureRegression
        The streaming regression it weighs with.
    options : dict
        The estimator's options (``warmup_std``).
    noise_name : str
        The noise preset of the weights (``estimated``: from the data).
    pressure_noise : tuple of float
        Pressure white-noise std (Pa) and pump-ripple share of the weights.
    difference_scale : numpy.ndarray
        Per-signal scale of the one-frame outlier test (:func:`difference_scale`).
    """

    TAG = "pressure_regression"

    def __init__(self, regression: PressureRegression, options: dict, noise_name: str,
                 pressure_noise: tuple[float, float] = (0.0, 0.0), difference_scale=None) -> None:
        self.regression = regression
        self.noise_name = noise_name
        self.pressure_noise = pressure_noise
        self.difference_scale = difference_scale
        self.warm_info = 1.0 / float(options["warmup_std"]) ** 2
        self.info = 0.0
        self._lone_moved = False

    @classmethod
    def build(cls, estimator, noise_name: str, pressure_noise: tuple[float, float],
              scale: np.ndarray) -> "PressureKernel":
        """The kernel of ``estimator``'s hydraulic machine with these weights and outlier scale.

        Parameters
        ----------
        estimator : InverseDynamicsEstimator
            The estimator (machine and options).
        noise_name : str
            The noise preset of the weights.
        pressure_noise : tuple of float
            Pressure white-noise std (Pa) and pump-ripple share.
        scale : numpy.ndarray
            Per-signal outlier-test scale.
        """
        std, ripple = pressure_noise
        options = estimator.options
        regression = PressureRegression(HydraulicArmModel(estimator.machine, compiled=False),
                                        pressure_std=std, ripple_fraction=ripple,
                                        half_window=options["half_window"], forgetting=options["forgetting"])
        regression.spike_threshold = spike_threshold(scale)
        return cls(regression, options, noise_name, pressure_noise, scale)

    @classmethod
    def fit(cls, estimator, dataset) -> "PressureKernel":
        """The kernel at the fitting data's noise (``--noise``, the preset the data name, or
        estimated from the data) and outlier scale.

        Parameters
        ----------
        estimator : InverseDynamicsEstimator
            The estimator (machine and options).
        dataset : Dataset
            Machine-sensor-set fitting data.
        """
        if not HYDRAULIC.owns(estimator.machine):
            raise EstimatorError(f"{estimator.name}: data of the machine sensor set need a hydraulic machine "
                                 f"file, not '{estimator.machine.name}' (e.g. --machine cat345c-hydraulic)")
        scale = difference_scale(dataset)
        name = estimator.options["noise"]
        if name == "auto":
            name = dataset.meta.get("noise")
        if name is None:  # issue 12: no preset named, the pressure noise is estimated from the data
            return cls.build(estimator, "estimated", (pressure_noise_from_data(dataset), 0.0), scale)
        preset = HYDRAULIC.noise(name)
        return cls.build(estimator, preset.name, (preset.pressure_noise, preset.ripple_fraction), scale)

    # -- streaming -------------------------------------------------------------------------
    def reset(self) -> None:
        """Empty the regression's window and sums."""
        self.info = 0.0
        self.regression.reset()
        self._lone_moved = False

    def bridge_gap(self) -> None:
        """The differentiator needs evenly spaced samples: its window starts again."""
        self.regression.restart_window()

    @property
    def model_std(self) -> float:
        """The calibration's model error, kg (0 for the machine file's own parameters)."""
        return self.regression.model_std

    @property
    def extra_std(self) -> float:
        """The regression's share of σ of the current estimate itself, kg (0 unless it has one)."""
        return float(getattr(self.regression, "extra_std", 0.0))

    def step(self, time: float, values: np.ndarray, judge: bool = True,
             joint_check: bool = False) -> StepResult:
        """One sample into the regression; the status of the estimate it leaves.

        Parameters
        ----------
        time : float
            Sample time, s.
        values : numpy.ndarray
            The sample, machine-set :data:`SIGNALS` order (SI units).
        judge : bool
            Whether the one-frame outlier test runs.
        joint_check : bool
            Whether the joints' balances are checked against each other (in the momentum form).
        """
        regression = self.regression
        regression.judge = judge
        regression.joint_check = joint_check and regression.checks_joints
        regression.update(time, values)
        self.info = regression.weighed_info
        if self.info <= 0.0 or not regression.ready or not regression.steady:
            return StepResult(math.nan, Status.WARMING_UP)
        status = Status.OK if self.info >= self.warm_info else Status.WARMING_UP
        if regression.rejected:  # the sample before this one was a one-frame outlier
            status = Status.REJECTED
        elif status is Status.OK and (regression.changing or getattr(regression, "dump_pending", False)):
            # the short memory has left the whole one, or the bucket dumps: the load changes
            status = Status.LOAD_CHANGING
        if regression.joint_check:
            status = self._joint_rules(status)
        fault = regression.joint_fault if regression.joint_check else ""
        if fault and status in (Status.OK, Status.LOAD_CHANGING):
            # the joints' balances disagree (a cylinder's pressure off, drifting or mis-scaled):
            # never ok; weighed without the joint named when one stands out, else nothing
            estimate, self.info = regression.joint_degraded
            return StepResult(estimate, Status.SENSOR_FAULT, fault=fault)
        return StepResult(regression.estimate, status)

    def _joint_rules(self, status: Status) -> Status:
        """The joint check's rules on an estimate the kernel would call ``status`` (the C export's
        ``ep_jc_status``): ``load_changing`` while the check pauses or the weighing moves before a
        fault is named (machine_calibration/joint_check.py). A joint weighed alone (a boom lift)
        cannot be compared with another: it is ``ok`` until its weighing moves; once it has moved
        it waits (``warming_up``) for a second joint to check it — also across a restart of the
        weighing, which a large fault sets off as a new load (a load cannot change while one
        joint moves alone). A fault on the lone joint is seen only as that move, and a move counts
        here only once the weighing is settled (its last windows hold at most ``LONE_YOUNG_SHARE``
        of its information: a new load's first second converges by more than the moving limit,
        docs/loadout.md). A weighing that
        moved while its joints were compared waits the same way until they are compared again
        after the check's pause (on sums gathered after the move)."""
        regression = self.regression
        if status is Status.OK:
            # a move counts whether or not the joints were compared then: after it the check
            # pauses and starts its sums again, and the joints it then compares must be those
            # sums' (a boom rate's bias that moved the whole weighing: 74 kg ok, seed 9300); a
            # young weighing's move (LONE_YOUNG_SHARE) is a new load converging
            if regression.joint_moved_settled:
                self._lone_moved = True
            elif regression.joint_checked and not regression.joint_pausing:
                self._lone_moved = False
        if status is Status.OK and (regression.joint_pausing or regression.joint_suspect):
            status = Status.LOAD_CHANGING
        if status is Status.OK and not regression.joint_checked and self._lone_moved \
                and not regression.joint_fault:  # a named joint is said (sensor_fault), not waited on
            status = Status.WARMING_UP
        return status

    # -- persistence -----------------------------------------------------------------------
    def config(self) -> dict:
        """The noise preset and the kernel's tag."""
        return {"noise": self.noise_name, "kernel": self.TAG}

    def arrays(self) -> dict[str, np.ndarray]:
        """The pressure noise of the weights and the outlier test's scale."""
        return {"pressure_noise": np.asarray(self.pressure_noise, float),
                "difference_scale": np.asarray(self.difference_scale, float)}

    @classmethod
    def restore(cls, estimator, config: dict, arrays: Mapping[str, np.ndarray]) -> "PressureKernel":
        """The kernel :meth:`config` and :meth:`arrays` saved (checked).

        Parameters
        ----------
        estimator : InverseDynamicsEstimator
            The estimator being loaded (machine and options).
        config : dict
            The saved state.
        arrays : Mapping[str, numpy.ndarray]
            The saved arrays.
        """
        noise = np.asarray(arrays["pressure_noise"], float)
        if noise.shape != (2,) or not np.all(np.isfinite(noise)) or not HYDRAULIC.owns(estimator.machine):
            raise EstimatorError("saved pressure-regression state is corrupt")
        return cls.build(estimator, str(config.get("noise", "unknown")), (float(noise[0]), float(noise[1])),
                         restore_difference_scale(arrays))
