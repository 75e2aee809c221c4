"""The slew rate's partner on a slope: the direction of the house's tilt (issue 31).

The machine set has no slew angle, so the monitor (:mod:`~excavator_payload.estimators.health`)
had nothing to hold a slew rate's scale error against. On a tilted house it has: the model's house
inclination (``HydraulicArmModel.house_inclination``, ``model/hydraulic.py``: pitch and roll are
the arcsines of the house rotation's z row, ``R_house = R_ground(tilt) · Rz(ψ)``) gives
(sin pitch, sin roll) = the ground's tilt vector turned by −ψ, so its size stays and its
direction ``atan2(sin roll, sin pitch)`` turns by exactly −ψ (checked against the model in
``tests/estimators/test_health_slew.py``). The slew angle the tilt says, θ = −that direction,
against the integrated slew rate is what a link's angle against its rate is to the ``gain`` rule:
over :data:`~excavator_payload.estimators.health.GAIN_WINDOW` the least-squares slope of
θ − ∫ψ̇ against θ is −e for a rate scaled by 1 + e.

The house IMU sits off the slew axis: its centripetal (∝ ψ̇², along the house's x: pitch) and
tangential (∝ ψ̈, along y: roll) accelerations leak into the tilt it reports (the simulator's
sensor model, ``simulation/machine_sensors.py``). Seen in the direction they are
K (sin roll · ψ̇² + sin pitch · ψ̈) / |tilt|² with one unknown K (the leak times the IMU's radius
over g), which the slope would otherwise pick up (clean 7° slopes: |slope| up to 0.12; with K fitted
in the same least squares, 0.03: docs/sensor-health.md, "The slew rate's scale error on a slope"). So the
window's fit has two regressors, θ and that leak term (ψ̈ the slew rate's difference over
± :data:`SLEW_ACCEL_HALF` samples; the fit uses the samples that have both neighbours).

Judged only while the tilt's size stays at least :data:`SLEW_TILT_MIN` over the whole window
(the direction of a small tilt is its sensors' noise and offsets) and θ's spread is at least
:data:`~excavator_payload.estimators.health.GAIN_MIN_STD` (the house slewed). Named ``gain`` on the
slew rate and both tilts (FMI 13): a tilt axis scaled alone also bends the direction, and the
data cannot tell which lies.
"""

from __future__ import annotations

import math

import numpy as np

#: Least size of the house's tilt (hypot of the sines of pitch and roll) over the whole window
#: for the direction to be judged, rad (about 2.9°).
SLEW_TILT_MIN = 0.05
#: The largest |slope| of θ − integrated slew rate against θ (a 10 % scale error is 0.1), and in
#: how many evaluations in a row (every ``EVERY`` samples).
SLEW_GAIN_LIMIT = 0.13
SLEW_GAIN_EVALUATIONS = 4
#: The slew acceleration of the leak term: the rate's difference over this many samples each side.
SLEW_ACCEL_HALF = 5
#: Least 1 − correlation² of θ and the leak term for both to be fitted; below it (the leak term
#: follows θ) the slope of θ alone.
SLEW_MIN_INDEPENDENCE = 1e-6


def house_terms(pitch: float, roll: float) -> tuple[float, float, float]:
    """One sample's (sin pitch, sin roll, direction of the tilt), computed once per sample (the
    monitor keeps them in a ring beside the raw samples).

    Parameters
    ----------
    pitch, roll : float
        The house's pitch and roll, rad.
    """
    sp, sr = math.sin(pitch), math.sin(roll)
    return sp, sr, math.atan2(sr, sp)


def slew_gain_slope(terms, rate, period: float, min_std: float) -> float:
    """The slope of (θ − integrated slew rate) against θ over a window, θ the slew angle the house
    tilt's direction says, the IMU's leak term fitted beside it (module docstring); NaN where the
    window is not judged (the tilt too small, or the house hardly slewed).

    Parameters
    ----------
    terms : numpy.ndarray
        (n, 3) :func:`house_terms` of the window's samples, oldest first.
    rate : numpy.ndarray
        The slew rate over the same samples, rad/s.
    period : float
        Sample period, s.
    min_std : float
        Least spread (standard deviation) of θ over the fitted samples, rad.

    Returns
    -------
    float
        The slope (−e for a slew rate scaled by 1 + e), or NaN.
    """
    sp, sr, direction = terms[:, 0], terms[:, 1], terms[:, 2]
    size2 = sp * sp + sr * sr
    if not size2.min() >= SLEW_TILT_MIN ** 2:
        return math.nan
    step = np.diff(direction)
    step -= 2.0 * math.pi * np.floor((step + math.pi) / (2.0 * math.pi))  # wrapped to [-π, π)
    theta = -np.cumsum(np.concatenate(([0.0], step)))
    turned = np.cumsum(np.concatenate(([0.0], 0.5 * period * (rate[1:] + rate[:-1]))))
    h = SLEW_ACCEL_HALF
    inner = slice(h, len(rate) - h)
    accel = (rate[2 * h:] - rate[:-2 * h]) / (2 * h * period)
    x = theta[inner]
    y = x - turned[inner]
    z = (sr[inner] * (rate[inner] * rate[inner]) + sp[inner] * accel) / size2[inner]
    m = len(x)
    x = x - x.sum() / m
    y = y - y.sum() / m
    z = z - z.sum() / m
    sxx = float(x @ x)
    if sxx / m < min_std ** 2:
        return math.nan
    szz, sxz, sxy, szy = float(z @ z), float(x @ z), float(x @ y), float(z @ y)
    den = sxx * szz - sxz * sxz
    if szz > 0.0 and den > SLEW_MIN_INDEPENDENCE * sxx * szz:
        return (szz * sxy - sxz * szy) / den
    return sxy / sxx
