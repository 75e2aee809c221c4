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
  is that the estimate refers to the sample ``half_window`` samples back (50 ms by default);
* **ground tilt** from the house IMU: at slew angle 0 the house's pitch and roll are those of
  the ground frame (:func:`ground_tilt`); the slew angle itself does not enter the dynamics
  (only its rate and acceleration do);
* **seal friction**: its presliding state is unknown, so the model's friction uses a smooth
  sign of the rod speed; near standstill the friction can be anything within ± the breakaway
  force, so that joint's residual variance grows by (breakaway torque)²/3, fading with speed
  (down-weighted, not skipped).

Weights: each joint's residual variance is the pressure noise (and pump ripple) through
:math:`\text{count}\,\partial l/\partial q\,(A_h, A_r)` plus the friction term above; the
estimate is :math:`\hat m = \sum \varphi^\top W r / \sum \varphi^\top W \varphi`, recursively.
Sensor offsets (zero drift) are *not* estimated here: that is the calibration and zero of issue 12.
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
        self.reset()

    def reset(self) -> None:
        self._buffer: deque = deque(maxlen=2 * self.half_window + 1)
        self.num = 0.0
        self.info = 0.0

    def _derivative(self) -> np.ndarray:
        """Least-squares slope of the rates over the buffer (centred), rad/s²."""
        t = np.array([b[0] for b in self._buffer])
        rates = np.array([b[1][RATES] for b in self._buffer])
        t = t - t.mean()
        return (t @ (rates - rates.mean(axis=0))) / (t @ t)

    def update(self, time: float, values: np.ndarray) -> bool:
        """Consume one sample; returns whether a sample (the centre of the window) was used."""
        self._buffer.append((time, values))
        if len(self._buffer) < self._buffer.maxlen:
            return False
        _, centre = self._buffer[self.half_window]
        qdd = self._derivative()
        q = np.zeros(4)
        q[:3] = centre[ANGLES]
        qd = centre[RATES]
        tilt = ground_tilt(centre[PITCH], centre[ROLL])
        pressures = centre[PRESSURES]
        out = self._f(q, qd, qdd, np.array(tilt), pressures, self._p)
        residual, phi, lever, speed, stiction = (np.asarray(o).ravel() for o in out)
        p_head, p_rod = pressures[0::2], pressures[1::2]
        side_var = self.pressure_var + self.ripple_var_share * np.stack([p_head, p_rod]) ** 2
        var = lever**2 * (self._head**2 * side_var[0] + self._rod**2 * side_var[1])
        still = np.exp(-(speed / (3 * self._v_stribeck)) ** 2)
        var = var + still * stiction**2 / 3
        w = 1.0 / var
        self.num = self.forgetting * self.num + float(np.sum(w * phi * residual))
        self.info = self.forgetting * self.info + float(np.sum(w * phi * phi))
        return True

    @property
    def estimate(self) -> float:
        return self.num / self.info if self.info > 0 else math.nan
