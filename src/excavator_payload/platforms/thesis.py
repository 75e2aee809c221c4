"""The thesis' platform: the 2-link arm, its joint-torque sensor set at 20 Hz, its noise presets.

Noise presets (standard deviations, SI units)
---------------------------------------------
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

import math
from dataclasses import dataclass
from typing import Any

from excavator_payload.data.schema import SIGNALS, THESIS_SENSORS
from excavator_payload.errors import ExcavatorPayloadError
from excavator_payload.platforms.base import SIMULATION_FAILURES, Motion, Platform, cheap_chunk_size, nmpc_chunk_size

# math, not numpy: the platforms are read at every command's start (numpy is imported where used).
DEG = math.pi / 180.0


@dataclass(frozen=True)
class NoisePreset:
    """Standard deviation of the additive white noise on each signal (SI units).

    Parameters
    ----------
    name : str
        The preset's name.
    std : dict of str to float
        Standard deviation of each thesis signal, in its SI unit (rad, rad/s, rad/s², N·m).
    description : str, default ""
        One line for humans.
    """

    name: str
    std: dict[str, float]
    description: str = ""

    def std_vector(self, columns=SIGNALS):
        """Standard deviations (SI units) of ``columns``, in that order (default :data:`SIGNALS`).

        Parameters
        ----------
        columns : sequence of str, default SIGNALS
            Signal names, each a key of :attr:`std`.
        """
        import numpy as np

        return np.array([self.std[c] for c in columns], dtype=float)

    @property
    def torque_covariance(self):
        """Σ of the two torque channels (N²m²), used by the Cramér–Rao bound and the filters."""
        import numpy as np

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
    "thesis": _preset("thesis", math.sqrt(1e-4) * DEG, math.sqrt(1e-5) * DEG, math.sqrt(1e-4) * DEG,
                      1000.0, 1000.0,
                      "appendix A.2 variances in the thesis' units: 0.01°, 0.0032°/s, 0.01°/s², 1000 N·m"),
    "none": _preset("none", 0.0, 0.0, 0.0, 0.0, 0.0, "noise-free sensors"),
    "field": _preset("field", 0.1 * DEG, 0.05 * DEG, math.sqrt(2) * 0.05 * DEG / 0.05,
                     15_000.0, 8_000.0,
                     "realistic machine sensors: 0.1°, 0.05°/s, 1.4°/s², 15/8 kN·m"),
}


def get_noise_preset(name: str | NoisePreset) -> NoisePreset:
    """The noise preset called ``name`` (``thesis``, ``none`` or ``field``).

    Parameters
    ----------
    name : str or NoisePreset
        A preset name, or a :class:`NoisePreset` (returned as it is).
    """
    if isinstance(name, NoisePreset):
        return name
    try:
        return PRESETS[name]
    except KeyError:
        raise ExcavatorPayloadError(
            f"unknown noise preset '{name}': choose one of {', '.join(PRESETS)}") from None



#: Samples discarded at the start of every experiment (thesis Table 7.1: "the first 81 steps",
#: at 20 Hz).
DEFAULT_DISCARD = 81


class ThesisPlatform(Platform):
    """The thesis' 2-link arm (:class:`~excavator_payload.model.machine.Machine`), joint angles,
    rates, accelerations and torques at 20 Hz (:data:`~excavator_payload.data.schema.THESIS_SENSORS`)."""

    name = "thesis"
    label = "this machine"
    kind = "2-link"
    sensors = THESIS_SENSORS
    noise_presets = PRESETS
    default_noise = "thesis"
    #: The motion families, by name (see :class:`~excavator_payload.platforms.base.Motion`).
    motions = {
        "nmpc": Motion("excavator_payload.simulation.generate:nmpc_experiment", nmpc_chunk_size,
                       skip_on=SIMULATION_FAILURES, description="the thesis' NMPC-driven swings"),
        "minimum-jerk": Motion("excavator_payload.simulation.minimum_jerk:minimum_jerk_experiment",
                               cheap_chunk_size, description="minimum-jerk swings with computed torques"),
        "lifts": Motion("excavator_payload.simulation.lifts:lift_experiment", cheap_chunk_size,
                        needs_first_zero=True, description="slow constant-speed calibration lifts"),
        "operator": Motion("excavator_payload.simulation.operator_swings:operator_experiment", cheap_chunk_size,
                           description="operator-like swings: a pause mid-way, an overshoot corrected back, "
                                       "small corrections at the end"),
    }

    def default_discard(self) -> int:
        """:data:`DEFAULT_DISCARD` samples, as in thesis Table 7.1."""
        return DEFAULT_DISCARD

    def noise(self, preset: Any = None) -> NoisePreset:
        """The noise preset ``preset`` (default ``thesis``).

        Parameters
        ----------
        preset : str or NoisePreset, optional
            ``thesis``, ``none`` or ``field``, or a preset object.
        """
        return get_noise_preset(self.default_noise if preset is None else preset)

    def owns(self, machine: Any) -> bool:
        """A 2-link arm: a machine object without cylinders.

        Parameters
        ----------
        machine : object
            A machine object.
        """
        from excavator_payload.model.machine import Machine

        return isinstance(machine, Machine)

    def simulation_settings(self, machine: Any, motion: str | None, noise: Any, *, session: int = 0,
                            trajectory: Any = None, payload: float | None = None,
                            smooth: float | None = None, allow_overspeed: bool = False,
                            truck_target: float | None = None,
                            frozen_noise_seed: int | None = None) -> tuple[str, NoisePreset, dict]:
        """Motion (default ``nmpc``) and noise (default ``thesis``); the hydraulic machine's
        settings are refused.

        Parameters
        ----------
        machine : Machine
            The arm simulated.
        motion : str or None
            Motion family (``None``: ``nmpc``).
        noise : str, NoisePreset or None
            Noise preset (``None``: ``thesis``).
        session : int
            Refused unless 0.
        trajectory : object or None
            Refused.
        payload : float or None
            Refused.
        smooth : float or None
            Refused.
        allow_overspeed : bool
            Refused.
        truck_target : float or None
            Refused.
        frozen_noise_seed : int or None
            Accepted (checked by the caller).
        """
        if smooth is not None or allow_overspeed:
            raise ExcavatorPayloadError("--smooth and --allow-overspeed go with a trajectory file (--trajectory)")
        if session or trajectory is not None or payload is not None or truck_target is not None:
            raise ExcavatorPayloadError("--session, --trajectory, --payload and --truck-target apply to a "
                                        "hydraulic machine only")
        return (self.default_motion if motion is None else motion), self.noise(noise), {}


#: The one instance.
THESIS = ThesisPlatform()
