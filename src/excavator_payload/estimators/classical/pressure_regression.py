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
  is that the estimate refers to the sample ``half_window + 1`` samples back (40 ms by
  default; the one more is the outlier test's look-ahead);
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
arrives, so it can afford to look one sample ahead: sample :math:`k` is rejected when some
signal :math:`i` jumps away from both neighbours in the same direction,

.. math:: (x_k - x_{k-1})(x_k - x_{k+1}) > 0, \quad
          \min(|x_k - x_{k-1}|, |x_k - x_{k+1}|) > z\,\sigma_{\Delta,i}
          \quad\text{and}\quad
          \min(|x_k - x_{k-1}|, |x_k - x_{k+1}|) > |x_{k+1} - x_{k-1}|,

with :math:`\sigma_{\Delta,i}` the robust spread of the signal's sample-to-sample changes on
the fitting data (:func:`difference_scale`) and :math:`z` the two-sided normal quantile of the
gate's probability (``GATE_PROBABILITY``). A step (a valve opening) moves away from one
neighbour only and a ramp from both in opposite directions, so hydraulic transients pass; a
model-based χ² test of the arriving sample did not work here: the rigid-body residual of a
transient runs tens of noise deviations for a quarter of a second (measured on NMPC swings:
NIS/dof 99th percentile ≈ 1000), which rejected good data and re-initialised the estimate.
The rejected sample's slot is filled by the mean of its neighbours (the differentiator needs
evenly spaced samples) and never regressed. The last condition asks the sample to stand out
from both neighbours more than they differ from each other: without it a glitch in the *next*
frame made a good sample in fast motion look like a spike (its change from the frame before
above the threshold, the glitch beyond it in the same direction), and the "repair" averaged
the glitch into the slot (a bucket-rate glitch at 0.2 s of an NMPC swing left inverse dynamics
at −589 kg instead of 3785 kg; the conformance suite on the machine set found it). Not caught: two or more bad frames in a row that
agree with each other (the plausibility limits still bound them).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from excavator_payload.data.schema import MACHINE_SENSORS
from excavator_payload.model.hydraulic import HydraulicArmModel, compiled_function

SIGNALS = MACHINE_SENSORS.signals
ANGLES = [SIGNALS.index(s) for s in ("boom_angle", "dipper_angle", "bucket_angle")]
RATES = [SIGNALS.index(s) for s in ("boom_rate", "dipper_rate", "bucket_rate", "slew_rate")]
PITCH, ROLL = SIGNALS.index("house_pitch"), SIGNALS.index("house_roll")
PRESSURES = [SIGNALS.index(s) for s in SIGNALS if s.endswith("_pressure")]


def ground_tilt(house_pitch: float, house_roll: float) -> tuple[float, float]:
    """Ground [pitch, roll] that gives the house this inclination at slew angle 0.

    Inverse of ``HydraulicArmModel.house_inclination`` at ψ = 0: the house's z row is
    (cos r sin p, sin r, cos r cos p), so roll = r and sin(pitch_house) = cos r sin p.
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
        # the differentiator's window and the newest sample, not yet judged
        self._buffer: deque = deque(maxlen=2 * self.half_window + 2)
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

    def _spike(self, before: np.ndarray, sample: np.ndarray, after: np.ndarray) -> bool:
        """Whether ``sample`` is a one-frame outlier between its neighbours (module doc)."""
        return one_frame_glitch(before, sample, after, self.spike_threshold)

    def update(self, time: float, values: np.ndarray) -> bool:
        """Consume one sample; returns whether a sample (the centre of the window) was used.
        :attr:`rejected` says whether the sample before this one was judged an outlier; the
        window regressed ends on that sample (every sample in it has been judged)."""
        self._buffer.append((time, values, True))
        self.rejected = False
        if self.judge and len(self._buffer) >= 3:
            (_, before, _), (t_mid, mid, _), (_, after, _) = (self._buffer[i] for i in (-3, -2, -1))
            if self._spike(before, mid, after):
                self._buffer[-2] = (t_mid, 0.5 * (before + after), False)
                self.rejected = True
        if len(self._buffer) < self._buffer.maxlen:
            return False
        _, centre, centre_used = self._buffer[self.half_window]
        if not centre_used:
            return False
        window = list(self._buffer)[:-1]
        qdd = self._slope([b[0] for b in window], [b[1][RATES] for b in window])
        residual, phi, var = self._evaluate(centre, qdd)
        w = 1.0 / var
        self.num = self.forgetting * self.num + float(np.sum(w * phi * residual))
        self.info = self.forgetting * self.info + float(np.sum(w * phi * phi))
        return True

    @property
    def estimate(self) -> float:
        return self.num / self.info if self.info > 0 else math.nan


def one_frame_glitch(before: np.ndarray, sample: np.ndarray, after: np.ndarray, threshold: np.ndarray) -> bool:
    """Whether ``sample`` is a one-frame outlier between its neighbours: some signal moves away
    from both, in the same direction, by more than its ``threshold`` (:func:`spike_threshold`)
    and more than the neighbours differ from each other (module doc). Shared by the pressure
    kernels and the machine-set Kalman filters."""
    d1 = sample - before
    if not (np.abs(d1) > threshold).any():  # the usual case, in three operations
        return False
    d2 = sample - after
    smaller = np.minimum(np.abs(d1), np.abs(d2))
    return bool(np.any((d1 * d2 > 0) & (smaller > threshold) & (smaller > np.abs(after - before))))


def difference_scale(dataset) -> np.ndarray:
    """Spread of each machine-set signal's sample-to-sample change (within experiments), as
    the std of a Gaussian with the same 99th percentile of the absolute change."""
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
    """Per-signal threshold z·σ_Δ of the one-frame outlier test (module doc)."""
    from scipy.stats import norm

    from excavator_payload.estimators.checks import GATE_PROBABILITY

    return norm.isf(GATE_PROBABILITY / 2) * np.asarray(scale, float)
