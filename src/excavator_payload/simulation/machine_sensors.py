r"""Sensor model of the machine sensor set: IMUs, slew gyro, cylinder pressure transmitters.

What a real installation adds to the true signals (each source and its magnitude below):

* **white noise** on every sample;
* a **per-session offset** on every sensor (zero drift: temperature, mounting, aging); it is
  constant during one working session and differs between sessions, so calibration lifts and
  later work, simulated with different ``session`` numbers, see different offsets. The offsets
  are drawn from the session number alone (:func:`session_offsets`), independently of the
  experiment seed;
* **pressure ripple** of the pump: harmonics of the piston frequency (pistons × shaft speed),
  attenuated by the transmitter's/logger's first-order anti-alias filter and sampled at 100 Hz
  (the residual aliases, as on a real logger), proportional to the pressure, random phases per
  experiment;
* **IMU dynamic error**: the IMU's internal filter lags the motion (first-order lag on angles
  and rates), and the accelerometer part of the inclination fusion leaks the link's tangential
  acceleration into its angle, and the house's centripetal and tangential acceleration into
  house pitch and roll (``leak`` × the apparent tilt atan(a/g)).

Presets: ``field`` (values below, with sources) and ``none`` (perfect sensors, no offsets).
"""

from __future__ import annotations

import numpy as np

from excavator_payload.data.schema import MACHINE_SENSORS

# The presets and session offsets are the hydraulic platform's; named here too.
from excavator_payload.platforms.hydraulic import (  # noqa: F401
    ANGLES,
    DEG,
    FIELD_SOURCES,
    INCLINATIONS,
    PRESETS,
    PRESSURES,
    RATES,
    MachineNoise,
    get_machine_noise,
    session_offsets,
)


def _lag(x: np.ndarray, dt: float, tau: float) -> np.ndarray:
    """First-order lag (exact for a piecewise-constant input), starting at steady state."""
    if tau <= 0:
        return x
    from scipy.signal import lfilter

    a = np.exp(-dt / tau)
    y, _ = lfilter([1 - a], [1, -a], x, axis=0, zi=np.asarray(x[:1]) * a)
    return y


def lag_delay(tau: float, dt: float) -> float:
    """The delay (s) by which :func:`_lag` holds a ramp back: the IMU lag an exact model of these
    signals must correct, ``dt·a / (1 − a)`` with ``a = exp(−dt / τ)`` (the filter takes the
    current sample, so its delay is not τ: 5.8 ms for τ = 10 ms at 100 Hz). An oracle that weighs
    with the simulator's own IMU dynamics takes this lag, not the preset's ``imu_lag``
    (docs/findings/any-motion.md, "Why `multisine` and `joystick` sit above the bound").

    Parameters
    ----------
    tau : float
        The preset's first-order time constant, s (0: no lag).
    dt : float
        Sample period, s.
    """
    if not (tau >= 0 and dt > 0):
        raise ValueError(f"lag_delay needs tau >= 0 and dt > 0, got tau={tau!r}, dt={dt!r}")
    if tau == 0:
        return 0.0
    a = float(np.exp(-dt / tau))
    return dt * a / (1.0 - a)


def measure(truth: dict[str, np.ndarray], time: np.ndarray, accelerations: np.ndarray,
            noise: MachineNoise, offsets: dict[str, float], rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Measured signals of one experiment from the true ones.

    Parameters
    ----------
    truth : dict
        True value of every signal of :data:`MACHINE_SENSORS` at the sample times.
    time : ndarray
        Sample times, s (uniform).
    accelerations : ndarray
        (n, 4) true accelerations of boom, dipper, bucket (relative) and slew, rad/s².
    noise, offsets, rng
        Preset, the session's offsets (:func:`session_offsets`) and the experiment's noise stream.
    """
    n = len(time)
    dt = float(time[1] - time[0]) if n > 1 else 0.01
    out: dict[str, np.ndarray] = {}
    g = 9.81
    absolute_accel = np.cumsum(accelerations[:, :3], axis=1)
    for j, name in enumerate(ANGLES):
        # Relative angle = difference of two link IMUs: each leaks its link's tangential
        # acceleration; the boom's reference is the house IMU (no arm acceleration).
        leak_own = np.arctan(noise.link_imu_distance * absolute_accel[:, j] / g)
        leak_parent = np.arctan(noise.link_imu_distance * absolute_accel[:, j - 1] / g) if j else 0.0
        dynamic = noise.acceleration_leak * (leak_own - leak_parent)
        out[name] = _lag(truth[name], dt, noise.imu_lag) + dynamic
    for name in RATES:
        out[name] = _lag(truth[name], dt, noise.imu_lag)
    slew_rate, slew_accel = truth["slew_rate"], accelerations[:, 3]
    # House IMU at radius r ahead of the slew axis: centripetal r ψ̇² along x (pitch),
    # tangential r ψ̈ along y (roll).
    out["house_pitch"] = (_lag(truth["house_pitch"], dt, noise.imu_lag)
                          + noise.acceleration_leak * np.arctan(noise.house_imu_radius * slew_rate**2 / g))
    out["house_roll"] = (_lag(truth["house_roll"], dt, noise.imu_lag)
                         - noise.acceleration_leak * np.arctan(noise.house_imu_radius * slew_accel / g))
    frequencies = noise.pump_pistons * noise.pump_shaft_frequency * np.arange(1, noise.ripple_harmonics + 1)
    gains = 1 / np.sqrt(1 + (frequencies / noise.antialias_cutoff) ** 2) / np.arange(1, noise.ripple_harmonics + 1)
    for name in PRESSURES:
        p = truth[name]
        phases = rng.uniform(0, 2 * np.pi, len(frequencies))
        ripple = (np.sin(2 * np.pi * frequencies[None, :] * time[:, None] + phases[None, :]) * gains).sum(axis=1)
        out[name] = p * (1 + noise.ripple_fraction * ripple)
    std = {**{s: noise.angle_noise for s in ANGLES}, **{s: noise.rate_noise for s in RATES},
           **{s: noise.inclination_noise for s in INCLINATIONS},
           **{s: noise.pressure_noise for s in PRESSURES}}
    white = rng.standard_normal((n, len(MACHINE_SENSORS.signals)))
    for i, name in enumerate(MACHINE_SENSORS.signals):
        out[name] = out[name] + offsets.get(name, 0.0) + std[name] * white[:, i]
    return out
