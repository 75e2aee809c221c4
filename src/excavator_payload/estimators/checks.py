"""The tables behind the input checks of :meth:`~excavator_payload.estimators.base.Estimator.step_values`.

Plausibility limits per signal (:func:`plausibility_limits`: the sensor set's, tightened by the
machine file through :data:`MACHINE_RULES` / :data:`HYDRAULIC_RULES`), the statistical gate's
probability and quantile (:data:`GATE_PROBABILITY`, :func:`gate_threshold`), how long a run of
rejections may last, and the plausible share of the rated payload. The order of the checks and
what each status means is in :mod:`excavator_payload.estimators.base`. This module imports no
estimator: the kernels (e.g. the machine set's one-frame outlier test) read their constants here.
"""

from __future__ import annotations

import math

import numpy as np

from excavator_payload.data.schema import SensorSet
from excavator_payload.model.machine import Machine
from excavator_payload.platforms import HYDRAULIC
from excavator_payload.platforms.hydraulic import ANGLES


#: An estimate outside these fractions of the machine's rated payload is never ``ok``: a bucket
#: holds no negative mass beyond the weighing's noise (a few % of rated), and 150 % of rated is
#: past any bucket's heaped capacity and the arm's lifting limit. Wrong factors in a signal map gave
#: -5 t with status ok and sigma 0.8 kg.
PLAUSIBLE_PAYLOAD = (-0.10, 1.50)

#: Probability, per sample, that a good sample is rejected by the statistical gate.
GATE_PROBABILITY = 1e-6
#: After rejections in a row for this long the estimator re-initialises instead of rejecting
#: (a glitch is one frame, a hydraulic transient a few tens of milliseconds; a new payload stays).
MAX_REJECTED_DURATION = 0.25
#: That many samples of the thesis sensor set (20 Hz); see :func:`max_consecutive_rejections`.
MAX_CONSECUTIVE_REJECTIONS = 5


def max_consecutive_rejections(sensor_set) -> int:
    """Rejections in a row after which an estimator on ``sensor_set`` re-initialises:
    :data:`MAX_REJECTED_DURATION` of samples (5 at 20 Hz, 25 at 100 Hz).

    Parameters
    ----------
    sensor_set : SensorSet
        The sensor set (its ``sample_rate``, Hz).

    Returns
    -------
    int
        At least 1.
    """
    return max(1, int(round(MAX_REJECTED_DURATION * sensor_set.sample_rate)))
#: The gate widens (never narrows below 1) to ``GATE_SCALE_HEADROOM`` × the recent accepted
#: innovations' share of the threshold, an exponential average with this weight per sample.
GATE_SCALE_RATE = 0.05
GATE_SCALE_HEADROOM = 4.0
#: A torque beyond this multiple of the machine's torque limit is not physical.
TORQUE_LIMIT_FACTOR = 1.5
#: Machine-file rules that tighten ``SensorSet.plausible_abs``: signal -> (rule, machine field).
#: ``range``: the field is a ``(low, high)`` pair; ``abs_limit``: ``|value| ≤ TORQUE_LIMIT_FACTOR
#: × field``. A rule whose signal is not in the sensor set does not apply.
MACHINE_RULES: dict[str, tuple[str, str]] = {
    "boom_angle": ("range", "boom_angle_range"),
    "dipper_angle": ("range", "dipper_angle_range"),
    "boom_torque": ("abs_limit", "boom_torque_limit"),
    "dipper_torque": ("abs_limit", "dipper_torque_limit"),
}

#: Hydraulic machine files: a measured link angle must lie inside the link's ``angle_range``
#: (the mechanical stops) widened by the sensor margin of :func:`angle_sensor_margins`.
HYDRAULIC_RULES: dict[str, tuple[str, str]] = {
    "boom_angle": ("link_range", "boom"),
    "dipper_angle": ("link_range", "dipper"),
    "bucket_angle": ("link_range", "bucket"),
}
#: Standard deviations of a sensor's offset and white noise the angle margin allows (a 6-sigma
#: Gaussian draw: about 2e-9 per sample).
ANGLE_MARGIN_SIGMAS = 6.0
#: Hydraulic machine files: a measured joint rate must lie within this factor times the fastest
#: the machine's hydraulics can turn the joint
#: (:meth:`~excavator_payload.model.hydraulic.HydraulicArmModel.largest_joint_rates`), plus the
#: rate sensors' offset and noise margin. The factor leaves room for what the pump-flow limit does
#: not bound (an overrunning load lowered faster than the pump fills the cylinder, a regenerating
#: valve, a machine file's flow on the low side); without it a glitch of two agreeing rate
#: frames (no one-frame test sees it) at 30 rad/s passed as plausible against the sensor set's
#: ±50 rad/s.
RATE_LIMIT_FACTOR = 2.0
HYDRAULIC_RATES = ("boom_rate", "dipper_rate", "bucket_rate", "slew_rate")
#: Hydraulic machine files: a measured cylinder pressure (gauge) must lie between a full vacuum
#: (−1 bar) and this factor times the machine's relief pressure, each widened by the pressure
#: sensors' offset and noise margin (:func:`sensor_margin`). Pressure peaks above the
#: relief setting (a valve's response time under a shock load, line reliefs set higher than the
#: main relief) stay well inside twice it; the sensor set alone allowed ±1000 bar, so two
#: agreeing frames of −300 bar passed as plausible.
PRESSURE_LIMIT_FACTOR = 2.0
VACUUM = 1.0e5  # Pa below atmospheric: no gauge pressure lies lower

_CHI2: dict[int, float] = {}


def angle_sensor_margins() -> dict[str, float]:
    r"""How far (rad) a measured link angle of the machine sensor set can lie outside the true one's
    range, the largest over the sensor model's presets
    (:mod:`excavator_payload.simulation.machine_sensors`).

    The measured angle is the IMU's first-order lag of the true angle, plus the accelerations'
    leak through the inclination fusion, plus the session offset and white noise. The lag adds
    nothing: its output is a convex combination of past true angles (weights :math:`(1-a)a^k`,
    started at steady state), so it stays inside their range, whatever the rate (the bound
    ``lag × max rate`` would only matter against a *moving* limit). The leak is
    ``acceleration_leak`` × the difference of two IMUs' apparent tilts
    :math:`rctan(d\,a/g)`, each below :math:`\pi/2` in magnitude (the boom's reference is
    the house IMU, which no arm acceleration reaches: one term). Offset and noise are allowed
    :data:`ANGLE_MARGIN_SIGMAS` standard deviations each.
    """
    margins = dict.fromkeys(ANGLES, 0.0)
    for noise in HYDRAULIC.noise_presets.values():
        for j, name in enumerate(ANGLES):
            leak = noise.acceleration_leak * (math.pi / 2) * (1 if j == 0 else 2)
            spread = ANGLE_MARGIN_SIGMAS * (noise.angle_offset + noise.angle_noise)
            margins[name] = max(margins[name], leak + spread)
    return margins


def sensor_margin(kind: str) -> float:
    """How far a measured ``kind`` (``rate``: rad/s, ``pressure``: Pa) of the machine sensor set
    can lie outside the true one's range, the largest over the sensor model's presets: offset
    and white noise, :data:`ANGLE_MARGIN_SIGMAS` standard deviations each (the IMU's lag is a
    convex combination of past true rates, and the pump ripple a share of the pressure itself
    that vanishes at 0: neither adds).

    Parameters
    ----------
    kind : str
        ``"rate"`` or ``"pressure"`` (the sensor model's field prefix).

    Returns
    -------
    float
        The margin, rad/s or Pa.
    """
    return max(ANGLE_MARGIN_SIGMAS * (getattr(n, f"{kind}_offset") + getattr(n, f"{kind}_noise"))
               for n in HYDRAULIC.noise_presets.values())


def gate_threshold(dof: int) -> float:
    """Chi-square quantile of ``1 - GATE_PROBABILITY`` with ``dof`` degrees of freedom.

    Parameters
    ----------
    dof : int
        Degrees of freedom of the innovation (its dimension).

    Returns
    -------
    float
        The threshold on the normalised innovation squared.
    """
    if dof not in _CHI2:
        from scipy.stats import chi2

        _CHI2[dof] = float(chi2.isf(GATE_PROBABILITY, dof))
    return _CHI2[dof]


def plausibility_limits(sensor_set: SensorSet, machine: Machine | None) -> tuple[np.ndarray, np.ndarray]:
    """``(low, high)`` per signal of ``sensor_set`` (its order) from the tables above.

    Parameters
    ----------
    sensor_set : SensorSet
        The sensor set whose signals are limited.
    machine : Machine or None
        Machine file that tightens the limits (None: the sensor set's only).

    Returns
    -------
    tuple of numpy.ndarray
        ``(low, high)``, SI units of each signal.
    """
    high = np.array([float(sensor_set.plausible_abs[s]) for s in sensor_set.signals])
    low = -high
    if machine is not None:
        hydraulic = HYDRAULIC.owns(machine)
        margins = angle_sensor_margins() if hydraulic else {}
        for signal, (rule, field_name) in (HYDRAULIC_RULES if hydraulic else MACHINE_RULES).items():
            if signal not in sensor_set.signals:
                continue
            i = sensor_set.index(signal)
            value = getattr(machine, field_name, None)
            if value is None:  # a kind of machine file without this field
                continue
            if rule == "link_range":
                lo, hi = value.angle_range
                low[i], high[i] = max(low[i], lo - margins[signal]), min(high[i], hi + margins[signal])
            elif rule == "range":
                low[i], high[i] = max(low[i], value[0]), min(high[i], value[1])
            else:
                limit = TORQUE_LIMIT_FACTOR * float(value)
                low[i], high[i] = max(low[i], -limit), min(high[i], limit)
        if hydraulic:
            from excavator_payload.model.hydraulic import HydraulicArmModel

            fastest = HydraulicArmModel(machine).largest_joint_rates()
            margin = sensor_margin("rate")
            for signal, rate in zip(HYDRAULIC_RATES, fastest):
                if signal in sensor_set.signals:
                    i = sensor_set.index(signal)
                    limit = RATE_LIMIT_FACTOR * rate + margin
                    low[i], high[i] = max(low[i], -limit), min(high[i], limit)
            margin = sensor_margin("pressure")
            top = PRESSURE_LIMIT_FACTOR * float(machine.hydraulics.relief_pressure) + margin
            for i, signal in enumerate(sensor_set.signals):
                if signal.endswith("_pressure"):
                    low[i], high[i] = max(low[i], -(VACUUM + margin)), min(high[i], top)
    return low, high
