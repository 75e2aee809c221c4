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

import numpy as np

# The presets are the thesis platform's (excavator_payload.platforms.thesis); named here too.
from excavator_payload.platforms.thesis import (  # noqa: F401
    DEG,
    FIELD_SOURCES,
    PRESETS,
    NoisePreset,
    get_noise_preset,
)


def add_noise(truth: np.ndarray, preset: NoisePreset, rng: np.random.Generator) -> np.ndarray:
    """Measured signals = truth + white Gaussian noise.

    Parameters
    ----------
    truth : numpy.ndarray
        True signals, shape (n_samples, 8), columns in ``SIGNALS`` order, SI units.
    preset : NoisePreset
        Standard deviation of the noise of each signal.
    rng : numpy.random.Generator
        Source of the noise.

    Returns
    -------
    numpy.ndarray
        Measured signals, same shape as ``truth``.
    """
    std = preset.std_vector()
    return truth + rng.standard_normal(truth.shape) * std
