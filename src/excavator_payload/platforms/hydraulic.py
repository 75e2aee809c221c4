"""The hydraulic machine's platform: 3 links on a slewing house, IMUs and cylinder pressures
at 100 Hz, the machine's sensor-noise presets (``field``, ``none``) and session offsets.

The sensor model that applies these magnitudes to a motion is
:mod:`excavator_payload.simulation.machine_sensors`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from numbers import Integral, Real
from typing import Any

from excavator_payload.data.schema import MACHINE_SENSORS
from excavator_payload.errors import ExcavatorPayloadError
from excavator_payload.platforms.base import (
    SIMULATION_FAILURES,
    Motion,
    Platform,
    machine_chunk_size,
    nmpc_chunk_size,
)

# math, not numpy: the platforms are read at every command's start (numpy is imported where used).
DEG = math.pi / 180.0
PRESSURES = tuple(s for s in MACHINE_SENSORS.signals if s.endswith("_pressure"))
ANGLES = ("boom_angle", "dipper_angle", "bucket_angle")
RATES = ("boom_rate", "dipper_rate", "bucket_rate", "slew_rate")
INCLINATIONS = ("house_pitch", "house_roll")

#: Passes per truck in a shift (``motion="shift"``): 2-6.
SHIFT_PASSES = (2, 6)
#: A pass's fill is at least this share of rated (a bucket the operator bothers to carry).
SHIFT_LEAST_FILL = 0.2


@dataclass(frozen=True)
class MachineNoise:
    """Magnitudes (1σ, SI units) of the machine sensor set's errors.

    Parameters
    ----------
    name : str
        The preset's name.
    angle_noise, angle_offset : float, default 0.0
        White noise and per-session offset of the link angles (1σ), rad.
    rate_noise, rate_offset : float, default 0.0
        White noise and per-session offset of the link and slew rates (1σ), rad/s.
    inclination_noise, inclination_offset : float, default 0.0
        White noise and per-session offset of the house pitch and roll (1σ), rad.
    pressure_noise, pressure_offset : float, default 0.0
        White noise and per-session offset of the cylinder pressures (1σ), Pa.
    ripple_fraction : float, default 0.0
        Pump ripple amplitude as a share of the pressure.
    pump_shaft_frequency : float, default 30.0
        The pump shaft's rotation frequency, Hz.
    pump_pistons : int, default 9
        Pistons of the pump: the ripple is at pistons × shaft frequency.
    ripple_harmonics : int, default 3
        Multiples of the piston frequency in the ripple (the fundamental included).
    antialias_cutoff : float, default 40.0
        Cut-off of the first-order anti-alias filter before sampling, Hz.
    imu_lag : float, default 0.0
        First-order time constant of the IMU output filter, s.
    acceleration_leak : float, default 0.0
        Share of the apparent tilt from acceleration left after the IMU's sensor fusion.
    link_imu_distance : float, default 1.5
        Distance of each link IMU from its link's joint, m.
    house_imu_radius : float, default 1.0
        Distance of the house IMU from the slew axis, m.
    description : str, default ""
        One line for humans.
    """

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
    """The machine-sensor noise preset ``name`` (``field`` or ``none``).

    Parameters
    ----------
    name : str or MachineNoise
        A preset name, or a :class:`MachineNoise` (returned as it is).
    """
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

    Parameters
    ----------
    session : int
        The working session's number (the seed of the draws).
    noise : MachineNoise
        The noise magnitudes; each offset is its 1σ offset times a standard normal draw.

    Returns
    -------
    dict of str to float
        Offset of each signal of the machine sensor set, in the signal's SI unit.
    """
    import numpy as np

    rng = np.random.default_rng(np.random.SeedSequence([int(session), 0x5E55_1011]))
    scale = {**{s: noise.angle_offset for s in ANGLES}, **{s: noise.rate_offset for s in RATES},
             **{s: noise.inclination_offset for s in INCLINATIONS},
             **{s: noise.pressure_offset for s in PRESSURES}}
    draws = rng.standard_normal(len(MACHINE_SENSORS.signals))
    return {s: float(d * scale[s]) for s, d in zip(MACHINE_SENSORS.signals, draws)}



#: Seconds not judged at the start of every experiment (its first second, 100 samples).
DEFAULT_DISCARD_SECONDS = 1.0

_SIM = "excavator_payload.simulation.machine_sim"


class HydraulicPlatform(Platform):
    """The hydraulic machine (:class:`~excavator_payload.model.hydraulic_machine.HydraulicMachine`)
    with the machine sensor set (:data:`~excavator_payload.data.schema.MACHINE_SENSORS`)."""

    name = "hydraulic"
    label = "a hydraulic machine"
    kind = "hydraulic"
    sensors = MACHINE_SENSORS
    noise_presets = PRESETS
    default_noise = "field"
    #: The motion families, by name (simulated by :mod:`excavator_payload.simulation.machine_sim`).
    motions = {
        "swing": Motion(f"{_SIM}:swing_experiment", machine_chunk_size, SIMULATION_FAILURES,
                        description="swings with slewing, within pump flow and relief pressure"),
        "nmpc": Motion(f"{_SIM}:nmpc_experiment", nmpc_chunk_size, SIMULATION_FAILURES,
                       description="NMPC swings with slewing, bounded by relief valves, pump flow and strokes"),
        "work-cycle": Motion(f"{_SIM}:work_cycle_experiment", machine_chunk_size, SIMULATION_FAILURES,
                             description="operator-like cycles: dig, lift while slewing, pause, dump, return"),
        "slopes": Motion(f"{_SIM}:slopes_experiment", machine_chunk_size, SIMULATION_FAILURES,
                         description="work cycles of a machine standing on a slope"),
        "lifts": Motion(f"{_SIM}:lifts_experiment", machine_chunk_size, SIMULATION_FAILURES,
                        description="slow calibration lifts"),
        "operator": Motion(f"{_SIM}:operator_experiment", machine_chunk_size, SIMULATION_FAILURES,
                           description="operator-like lift and slew: a pause, an overshoot, trims all along"),
        "reach": Motion(f"{_SIM}:reach_experiment", machine_chunk_size, SIMULATION_FAILURES,
                        description="calibration motions: every joint through its range at once, slewing"),
        "calibration": Motion(f"{_SIM}:calibration_experiment", machine_chunk_size, SIMULATION_FAILURES,
                              description="the recommended calibration mix: swings, 3 in 10 reach motions"),
        "trajectory": Motion("excavator_payload.simulation.trajectory:trajectory_experiment",
                             machine_chunk_size, SIMULATION_FAILURES,
                             description="prescribed motions replayed from a trajectory file"),
        "shift": Motion(f"{_SIM}:shift_experiment", machine_chunk_size, SIMULATION_FAILURES,
                        description="a day of loading: one truck of 2-6 work cycles per experiment"),
    }

    def default_discard(self) -> int:
        """The first :data:`DEFAULT_DISCARD_SECONDS` of every experiment, in samples."""
        return int(round(DEFAULT_DISCARD_SECONDS * self.sample_rate))

    def noise(self, preset: Any = None) -> MachineNoise:
        """The noise preset ``preset`` (default ``field``).

        Parameters
        ----------
        preset : str or MachineNoise, optional
            ``field`` or ``none``, or a preset object.
        """
        return get_machine_noise(self.default_noise if preset is None else preset)

    def owns(self, machine: Any) -> bool:
        """A hydraulic machine object.

        Parameters
        ----------
        machine : object
            A machine object.
        """
        from excavator_payload.model.hydraulic_machine import HydraulicMachine

        return isinstance(machine, HydraulicMachine)

    def simulation_settings(self, machine: Any, motion: str | None, noise: Any, *, session: int = 0,
                            trajectory: Any = None, payload: float | None = None,
                            smooth: float | None = None, allow_overspeed: bool = False,
                            truck_target: float | None = None,
                            frozen_noise_seed: int | None = None) -> tuple[str, MachineNoise, dict]:
        """Motion (default ``swing``, ``trajectory`` with a trajectory), noise (default
        ``field``) and the options ``session``, ``payload`` and ``truck_target``, checked.

        Parameters
        ----------
        machine : HydraulicMachine
            The machine simulated.
        motion : str or None
            Motion family.
        noise : str, MachineNoise or None
            Noise preset.
        session : int
            Working session (draws the sensor offsets), ≥ 0.
        trajectory : object or None
            A trajectory (file or object) to replay; goes with ``motion="trajectory"``.
        payload : float or None
            Every generated experiment's mass, kg, within the machine's maximum payload.
        smooth : float or None
            Goes with a trajectory only.
        allow_overspeed : bool
            Goes with a trajectory only.
        truck_target : float or None
            Goes with ``motion="shift"`` only; at most 6 passes of the maximum payload.
        frozen_noise_seed : int or None
            Refused: the machine's sensors always draw their own noise.
        """
        options: dict = {}
        if motion is None:
            motion = "trajectory" if trajectory is not None else self.default_motion
        if (motion == "trajectory") != (trajectory is not None):
            raise ExcavatorPayloadError("a trajectory file goes with --motion trajectory (and only with it)")
        if frozen_noise_seed is not None:
            raise ExcavatorPayloadError("frozen noise is a thesis-setting study; the hydraulic machine's "
                                        "sensors always draw their own noise")
        if isinstance(session, bool) or not isinstance(session, Integral) or session < 0:
            raise ExcavatorPayloadError(f"the session must be a whole number ≥ 0, got {session!r}")
        preset = self.noise(noise)
        options["session"] = int(session)
        if payload is not None:
            if trajectory is not None:
                raise ExcavatorPayloadError("--payload does not go with a trajectory file: its payload "
                                            "column sets the mass")
            if (isinstance(payload, bool) or not isinstance(payload, Real)
                    or not 0.0 <= float(payload) <= machine.max_payload):
                raise ExcavatorPayloadError(f"--payload must be between 0 and the machine's maximum "
                                            f"payload, {machine.max_payload:g} kg; got {payload!r}")
            options["payload"] = float(payload)
        if trajectory is None and (smooth is not None or allow_overspeed):
            raise ExcavatorPayloadError("--smooth and --allow-overspeed go with a trajectory file (--trajectory)")
        if truck_target is not None or motion == "shift":
            if motion != "shift":
                raise ExcavatorPayloadError("--truck-target goes with --motion shift (and only with it)")
            if payload is not None:
                raise ExcavatorPayloadError("--payload does not go with --motion shift: each pass draws "
                                            "its fill towards --truck-target")
            if truck_target is not None:
                fewest, most_passes = SHIFT_PASSES
                most = machine.max_payload * most_passes
                # Below two of the smallest passes every fill is clipped: a 1.2 t target made
                # trucks of 2 t without a word.
                least = fewest * SHIFT_LEAST_FILL * float(machine.rated_payload)
                if (isinstance(truck_target, bool) or not isinstance(truck_target, Real)
                        or not least <= float(truck_target) <= most):
                    raise ExcavatorPayloadError(
                        f"--truck-target must be between {least:g} kg ({fewest} passes of "
                        f"{100 * SHIFT_LEAST_FILL:g} % of rated) and {most:g} kg ({most_passes} passes of "
                        f"the machine's maximum payload); got {truck_target!r}")
                options["truck_target"] = float(truck_target)
        return motion, preset, options

    def run_meta(self, spec: Any) -> dict:
        """The session, its true sensor offsets and a replayed trajectory's source.

        Parameters
        ----------
        spec : RunSpec
            The run.
        """
        session = int(spec.option("session", 0))
        meta = {"session": session,
                # The true offsets of this session: for checking offset estimation, not for estimators.
                "true_sensor_offsets": session_offsets(session, spec.noise)}
        trajectory = spec.option("trajectory")
        if trajectory is not None:
            meta["trajectory"] = trajectory.source
        return meta

    def check_plausible(self, frame: Any, machine: Any, source: str) -> None:
        """Head and rod pressures not swapped (:func:`~excavator_payload.data.wiring.check_wiring`).

        Parameters
        ----------
        frame : pandas.DataFrame
            ``experiment``, ``time`` and the machine sensor set's signals.
        machine : HydraulicMachine or None
            The machine believed to have made the data (no check without one).
        source : str
            Named in the error message.
        """
        from excavator_payload.data.wiring import check_wiring

        check_wiring(frame, self.sensors, machine, source)


#: The one instance.
HYDRAULIC = HydraulicPlatform()
