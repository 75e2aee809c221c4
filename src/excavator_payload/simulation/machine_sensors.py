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

from dataclasses import asdict, dataclass

import numpy as np

from excavator_payload.data.schema import MACHINE_SENSORS
from excavator_payload.errors import ExcavatorPayloadError

DEG = np.pi / 180.0
PRESSURES = tuple(s for s in MACHINE_SENSORS.signals if s.endswith("_pressure"))
ANGLES = ("boom_angle", "dipper_angle", "bucket_angle")
RATES = ("boom_rate", "dipper_rate", "bucket_rate", "slew_rate")
INCLINATIONS = ("house_pitch", "house_roll")


@dataclass(frozen=True)
class MachineNoise:
    """Magnitudes (1σ, SI units) of the machine sensor set's errors."""

    name: str
    angle_noise: float = 0.0
    angle_offset: float = 0.0
    rate_noise: float = 0.0
    rate_offset: float = 0.0
    inclination_noise: float = 0.0
    inclination_offset: float = 0.0
    pressure_noise: float = 0.0
    pressure_offset: float = 0.0
    ripple_fraction: float = 0.0  # ripple amplitude at the pump / pressure
    pump_shaft_frequency: float = 30.0  # Hz
    pump_pistons: int = 9
    ripple_harmonics: int = 3
    antialias_cutoff: float = 40.0  # Hz, first-order
    imu_lag: float = 0.0  # s, first-order time constant of the IMU output filter
    acceleration_leak: float = 0.0  # share of the apparent tilt from acceleration left after fusion
    link_imu_distance: float = 1.5  # m, IMU from its link's joint
    house_imu_radius: float = 1.0  # m, house IMU from the slew axis
    description: str = ""

    def to_dict(self) -> dict:
        """All magnitudes as a dict of field name -> value."""
        return asdict(self)


#: Sources of the ``field`` magnitudes.
FIELD_SOURCES = {
    "angle": "0.05° noise, 0.1° session offset: fused MEMS inclination sensors for mobile machines "
             "(e.g. ifm JN2301, Sick TMM88D: ±0.1° static accuracy; mounting repeatability ~0.1°)",
    "rate": "0.1°/s noise: MEMS gyro noise density ~0.014 °/s/√Hz (Bosch BMI088) over 50 Hz; "
            "0.1°/s turn-on bias between sessions (datasheet bias stability ±0.5°/s uncompensated, "
            "~0.1°/s after the sensor's own temperature compensation)",
    "inclination": "0.02° noise, 0.1° offset: house IMU as the link IMUs, static (less vibration)",
    "pressure": "30 kPa noise (0.05 % of 600 bar full scale) and 150 kPa offset (0.25 % FS, the "
                "lower end of 0.25-0.5 % FS total error of mobile-hydraulics transmitters, e.g. "
                "WIKA MH-3, Danfoss MBS 1200)",
    "ripple": "2 % of the pressure at the pump's piston frequency 9 × 30 Hz (axial piston pump, "
              "engine 1800 rpm) and 2 harmonics, through a 40 Hz first-order anti-alias filter",
    "imu_dynamic": "10 ms output lag (IMU internal low-pass), 5 % of the acceleration's apparent "
                   "tilt leaking through the gyro/accelerometer fusion",
}

PRESETS: dict[str, MachineNoise] = {
    "field": MachineNoise(
        "field", angle_noise=0.05 * DEG, angle_offset=0.1 * DEG, rate_noise=0.1 * DEG,
        rate_offset=0.1 * DEG, inclination_noise=0.02 * DEG, inclination_offset=0.1 * DEG,
        pressure_noise=3.0e4, pressure_offset=1.5e5, ripple_fraction=0.02, imu_lag=0.01,
        acceleration_leak=0.05,
        description="machine sensors with noise, session offsets, pump ripple and IMU dynamics"),
    "none": MachineNoise("none", description="perfect sensors: no noise, offsets, ripple or lag"),
}


def get_machine_noise(name: "str | MachineNoise") -> MachineNoise:
    """The machine-sensor noise preset ``name`` (``field`` or ``none``)."""
    if isinstance(name, MachineNoise):
        return name
    try:
        return PRESETS[str(name)]
    except KeyError:
        raise ExcavatorPayloadError(
            f"unknown noise preset '{name}' for the machine sensor set: choose one of "
            f"{', '.join(PRESETS)}") from None


def session_offsets(session: int, noise: MachineNoise) -> dict[str, float]:
    """The offset of every sensor during working session ``session`` (SI units).

    Drawn from the session number alone (not from the experiment seed): every experiment of
    a session shares them, and another session draws other ones.
    """
    rng = np.random.default_rng(np.random.SeedSequence([int(session), 0x5E55_1011]))
    scale = {**{s: noise.angle_offset for s in ANGLES}, **{s: noise.rate_offset for s in RATES},
             **{s: noise.inclination_offset for s in INCLINATIONS},
             **{s: noise.pressure_offset for s in PRESSURES}}
    draws = rng.standard_normal(len(MACHINE_SENSORS.signals))
    return {s: float(d * scale[s]) for s, d in zip(MACHINE_SENSORS.signals, draws)}


def _lag(x: np.ndarray, dt: float, tau: float) -> np.ndarray:
    """First-order lag (exact for a piecewise-constant input), starting at steady state."""
    if tau <= 0:
        return x
    from scipy.signal import lfilter

    a = np.exp(-dt / tau)
    y, _ = lfilter([1 - a], [1, -a], x, axis=0, zi=np.asarray(x[:1]) * a)
    return y


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
