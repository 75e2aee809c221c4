"""Sensor model: 20 Hz sampling with additive white Gaussian noise, by preset.

Presets (standard deviations, SI units)
---------------------------------------
``thesis``
    Appendix A.2's variances applied in the thesis' signal units (degrees, N·m): angle
    10⁻⁴ deg², rate 10⁻⁵ (deg/s)², acceleration 10⁻⁴ (deg/s²)², torque 10⁶ N²m², i.e.
    σ = 0.01°, 0.0032°/s, 0.01°/s², 1000 N·m (§5.3: PSD 5×10⁻⁶ … at Ts = 0.05 s, σ² = PSD/Ts).
``none``
    Noise-free sensors.
``field``
    Sensors an excavator really carries, see :data:`FIELD_SOURCES`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from excavator_payload.data.schema import SIGNALS
from excavator_payload.errors import ExcavatorPayloadError

DEG = np.pi / 180.0


@dataclass(frozen=True)
class NoisePreset:
    """Standard deviation of the additive white noise on each signal (SI units)."""

    name: str
    std: dict[str, float]
    description: str = ""

    def std_vector(self, columns=SIGNALS) -> np.ndarray:
        """Standard deviations (SI units) of ``columns``, in that order (default :data:`SIGNALS`)."""
        return np.array([self.std[c] for c in columns], dtype=float)

    @property
    def torque_covariance(self) -> np.ndarray:
        """Σ of the two torque channels (N²m²), used by the Cramér–Rao bound and the filters."""
        return np.diag([self.std["boom_torque"] ** 2, self.std["dipper_torque"] ** 2])


def _preset(name, angle, rate, accel, boom_torque, dipper_torque, description):
    return NoisePreset(name, {
        "boom_angle": angle, "dipper_angle": angle,
        "boom_rate": rate, "dipper_rate": rate,
        "boom_accel": accel, "dipper_accel": accel,
        "boom_torque": boom_torque, "dipper_torque": dipper_torque,
    }, description)


#: Where the ``field`` figures come from (shown in the README and ``--help``).
FIELD_SOURCES = {
    "angle": "0.1° (1σ): dynamic MEMS inclination sensors with gyro fusion for mobile machines "
             "(e.g. ifm JN2301, Sick TMM88D) state ±0.1°…0.5° dynamic accuracy",
    "rate": "0.05°/s (1σ): MEMS gyro noise density ≈0.01 °/s/√Hz over a ≈10 Hz bandwidth "
            "(e.g. Bosch BMI088: 0.014 °/s/√Hz) plus quantisation",
    "accel": "1.4°/s² (1σ): angular acceleration is not measured on machines; it is the "
             "backward difference of the rate at 20 Hz, σ = √2·0.05°/s / 0.05 s",
    "torque": "boom 15 kN·m, dipper 8 kN·m (1σ): torques from cylinder pressure transducers "
              "(0.5 % of 400 bar full scale = 2 bar) on ≈0.057 m² (boom, two 190 mm bores) and "
              "≈0.031 m² (dipper) of piston area, through ≈1.3 m and ≈1.3 m lever arms, plus "
              "seal friction",
}

PRESETS: dict[str, NoisePreset] = {
    "thesis": _preset("thesis", np.sqrt(1e-4) * DEG, np.sqrt(1e-5) * DEG, np.sqrt(1e-4) * DEG,
                      1000.0, 1000.0,
                      "appendix A.2 variances in the thesis' units: 0.01°, 0.0032°/s, 0.01°/s², 1000 N·m"),
    "none": _preset("none", 0.0, 0.0, 0.0, 0.0, 0.0, "noise-free sensors"),
    "field": _preset("field", 0.1 * DEG, 0.05 * DEG, np.sqrt(2) * 0.05 * DEG / 0.05,
                     15_000.0, 8_000.0,
                     "realistic machine sensors: 0.1°, 0.05°/s, 1.4°/s², 15/8 kN·m"),
}


def get_noise_preset(name: str | NoisePreset) -> NoisePreset:
    """The noise preset called ``name`` (``thesis``, ``none`` or ``field``)."""
    if isinstance(name, NoisePreset):
        return name
    try:
        return PRESETS[name]
    except KeyError:
        raise ExcavatorPayloadError(
            f"unknown noise preset '{name}': choose one of {', '.join(PRESETS)}") from None


def add_noise(truth: np.ndarray, preset: NoisePreset, rng: np.random.Generator) -> np.ndarray:
    """Measured signals = truth + white Gaussian noise; ``truth`` is (n_samples, 8) in SIGNALS order."""
    std = preset.std_vector()
    return truth + rng.standard_normal(truth.shape) * std
