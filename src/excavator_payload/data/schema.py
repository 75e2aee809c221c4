"""The dataset schema: sensor sets, one row per sample, SI units, fixed column names.

A :class:`SensorSet` names the signals one kind of installation measures, their units, sample
rate and plausibility limits. Two exist:

* ``thesis`` (:data:`THESIS_SENSORS`): the thesis' 2-link arm with joint torque sensors and
  measured accelerations, 20 Hz;
* ``machine`` (:data:`MACHINE_SENSORS`): what a real excavator has: link angles and rates from
  IMUs, slew rate, house pitch and roll, and the pressures on both sides of each hydraulic
  cylinder, 100 Hz. A logger on a real machine writes these columns.

A dataset says which set it holds (metadata key ``sensor_set``; older files without it are
recognised by their columns), and every estimator declares the sets it can run on. Code that
handles signals takes them from the dataset's or estimator's sensor set, never from a fixed
list; the module constants ``SIGNALS``, ``COLUMNS`` … are the thesis set's, kept for the thesis
code paths.

Per-experiment metadata (seed, start and target pose, payload, machine, noise preset, solver
status) travels inside the Parquet file's schema metadata under the key
``excavator_payload`` as JSON (see :mod:`excavator_payload.data.io`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterable, Mapping

#: The eight measured signals, in the thesis' column order (appendix A.2 ``input_names``).
SIGNALS: tuple[str, ...] = (
    "boom_angle",
    "boom_rate",
    "boom_accel",
    "dipper_angle",
    "dipper_rate",
    "dipper_accel",
    "boom_torque",
    "dipper_torque",
)

#: SI unit of every column.
UNITS: dict[str, str] = {
    "experiment": "",
    "time": "s",
    "boom_angle": "rad",
    "boom_rate": "rad/s",
    "boom_accel": "rad/s^2",
    "dipper_angle": "rad",
    "dipper_rate": "rad/s",
    "dipper_accel": "rad/s^2",
    "boom_torque": "N*m",
    "dipper_torque": "N*m",
    "payload": "kg",
}

#: Resolution (one raw bit) of every SI unit the sensor sets use: the CAN codec's scale
#: (:mod:`excavator_payload.runtime.dbc`) and the health monitor's quantisation step.
RESOLUTION: dict[str, float] = {
    "rad": 1e-5,        # 0.00057°; thesis angle noise 1.7e-4 rad
    "rad/s": 1e-5,      # thesis rate noise 5.6e-5 rad/s
    "rad/s^2": 1e-5,    # thesis acceleration noise 1.7e-4 rad/s²
    "N*m": 1.0,         # thesis torque noise 1000 N·m
    "Pa": 100.0,        # 1 mbar; pressure transducers are ±0.5 % of 400 bar = 2 bar
}

#: Required columns of every dataset, in order.
COLUMNS: tuple[str, ...] = ("experiment", "time", *SIGNALS, "payload")

#: Optional noise-free columns written with ``--with-truth``.
TRUTH_COLUMNS: tuple[str, ...] = tuple(f"true_{s}" for s in SIGNALS)

SAMPLE_RATE = 20.0  # Hz
SAMPLE_PERIOD = 1.0 / SAMPLE_RATE  # s
DURATION = 5.0  # s, one experiment
SAMPLES_PER_EXPERIMENT = 101  # t = 0 … 5 s

#: Columns of an estimates file (``excavator-payload estimate``).
ESTIMATE_COLUMNS: tuple[str, ...] = ("experiment", "time", "payload_estimate")

#: Plausibility limits used by validation (far outside anything an excavator arm does).
PLAUSIBLE_ABS = {
    "boom_angle": 10.0,
    "dipper_angle": 10.0,
    "boom_rate": 50.0,
    "dipper_rate": 50.0,
    "boom_accel": 5000.0,
    "dipper_accel": 5000.0,
    "boom_torque": 1e9,
    "dipper_torque": 1e9,
}

METADATA_KEY = b"excavator_payload"
FORMAT_VERSION = 1


# -- sensor sets ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class SensorSet:
    """The signals of one kind of installation.

    Parameters
    ----------
    name : str
        Registry name (``thesis``, ``machine``), stored in dataset metadata.
    description : str
        One line for humans.
    signals : tuple of str
        Measured signals in column order (the order of every signal vector in the code).
    units : mapping
        SI unit of each signal.
    sample_rate : float
        Nominal sample rate, Hz.
    plausible_abs : mapping
        Largest absolute value of each signal that can be physical at all (validation rejects
        more: it is a unit mistake or a broken sensor, not data).
    truth_extra : tuple of str
        Noise-free columns written with ``--with-truth`` besides ``true_<signal>`` (for
        example the true joint torques and accelerations, which this set does not measure).
    extra_units : mapping
        SI unit of each :attr:`truth_extra` column.
    truth_added : tuple of str
        Columns of :attr:`truth_extra` added after files were written without them: a file
        lacking them still has its truth (:attr:`required_truth_columns`).
    rate_pairs : tuple of (signal, rate, unit, least change)
        Each rate checked against the change of the signal it is the rate of (validation: a rate
        in degrees beside an angle in radians): the signal, its rate, the rate's unit and the
        least change of the signal over a window for the window to be judged (signal's unit).
    """

    name: str
    description: str
    signals: tuple[str, ...]
    units: Mapping[str, str]
    sample_rate: float
    plausible_abs: Mapping[str, float]
    truth_extra: tuple[str, ...] = ()
    extra_units: Mapping[str, str] = field(default_factory=dict)
    rate_pairs: tuple[tuple[str, str, str, float], ...] = ()
    truth_added: tuple[str, ...] = ()

    @property
    def sample_period(self) -> float:
        """Nominal time between samples, s."""
        return 1.0 / self.sample_rate

    @property
    def columns(self) -> tuple[str, ...]:
        """Columns of a dataset of this set: ``experiment``, ``time``, signals, ``payload``."""
        return ("experiment", "time", *self.signals, "payload")

    @property
    def truth_columns(self) -> tuple[str, ...]:
        """Noise-free columns of ``--with-truth``: ``true_<signal>`` then :attr:`truth_extra`."""
        return tuple(f"true_{s}" for s in self.signals) + self.truth_extra

    @property
    def required_truth_columns(self) -> tuple[str, ...]:
        """The truth columns a file must have to count as with truth (all but :attr:`truth_added`)."""
        return tuple(c for c in self.truth_columns if c not in self.truth_added)

    @property
    def cylinder_chambers(self) -> tuple[str, ...]:
        """Cylinders whose head and rod pressures this set measures (``()``: none, as the thesis'
        joint-torque sensors), in signal order."""
        heads = [s.removesuffix("_head_pressure") for s in self.signals if s.endswith("_head_pressure")]
        return tuple(c for c in heads if f"{c}_rod_pressure" in self.signals)

    def index(self, signal: str) -> int:
        """Position of ``signal`` in :attr:`signals`.

        Parameters
        ----------
        signal : str
            A signal name of this set.
        """
        return self.signals.index(signal)

    def indices(self, signals: Iterable[str]) -> list[int]:
        """Positions of several signals.

        Parameters
        ----------
        signals : iterable of str
            Signal names of this set.

        Returns
        -------
        list of int
            Their positions in :attr:`signals`, in the given order.
        """
        return [self.signals.index(s) for s in signals]

    def unit(self, column: str) -> str:
        """SI unit of any column of this set (signals, truth columns, ``time``, ``payload``).

        Parameters
        ----------
        column : str
            A column name; unknown columns have the unit ``""``.
        """
        base = column.removeprefix("true_")
        return {"experiment": "", "time": "s", "payload": "kg", **self.extra_units,
                **self.units}.get(base, self.extra_units.get(column, ""))


#: The thesis' installation: 2-link arm, joint torque sensors, measured accelerations, 20 Hz.
THESIS_SENSORS = SensorSet(
    name="thesis",
    description="thesis 2-link arm: joint angles, rates, accelerations and torques, 20 Hz",
    signals=SIGNALS,
    units={s: UNITS[s] for s in SIGNALS},
    sample_rate=SAMPLE_RATE,
    plausible_abs=dict(PLAUSIBLE_ABS),
    rate_pairs=(("boom_angle", "boom_rate", "rad/s", 0.02), ("dipper_angle", "dipper_rate", "rad/s", 0.02),
                ("boom_rate", "boom_accel", "rad/s^2", 0.05), ("dipper_rate", "dipper_accel", "rad/s^2", 0.05)),
)

#: Signals of a real machine (issue "The machine as it is"): IMU angles and rates of each link
#: relative to the body before it (boom relative to the house), slew rate, house inclination,
#: and both chamber pressures of each cylinder (the two boom cylinders share their lines).
MACHINE_SIGNALS: tuple[str, ...] = (
    "boom_angle",
    "dipper_angle",
    "bucket_angle",
    "boom_rate",
    "dipper_rate",
    "bucket_rate",
    "slew_rate",
    "house_pitch",
    "house_roll",
    "boom_head_pressure",
    "boom_rod_pressure",
    "dipper_head_pressure",
    "dipper_rod_pressure",
    "bucket_head_pressure",
    "bucket_rod_pressure",
)

MACHINE_SENSORS = SensorSet(
    name="machine",
    description="hydraulic machine: IMU link angles and rates, slew rate, house pitch and roll, "
                "cylinder head and rod pressures, 100 Hz",
    signals=MACHINE_SIGNALS,
    units={
        **{s: "rad" for s in ("boom_angle", "dipper_angle", "bucket_angle", "house_pitch", "house_roll")},
        **{s: "rad/s" for s in ("boom_rate", "dipper_rate", "bucket_rate", "slew_rate")},
        **{s: "Pa" for s in MACHINE_SIGNALS if s.endswith("_pressure")},
    },
    sample_rate=100.0,
    plausible_abs={
        # Angles: a link never turns more than a full circle relative to its parent.
        **{s: 2 * math.pi for s in ("boom_angle", "dipper_angle", "bucket_angle")},
        # A machine standing on more than ~57° of slope has fallen over.
        "house_pitch": 1.0,
        "house_roll": 1.0,
        **{s: 50.0 for s in ("boom_rate", "dipper_rate", "bucket_rate", "slew_rate")},
        # 1000 bar: three times any relief valve of a mobile machine (~350-450 bar).
        **{s: 1.0e8 for s in MACHINE_SIGNALS if s.endswith("_pressure")},
    },
    truth_extra=("true_boom_torque", "true_dipper_torque", "true_bucket_torque",
                 "true_boom_accel", "true_dipper_accel", "true_bucket_accel", "true_slew_accel",
                 "true_slew_angle", "true_bucket_load"),
    extra_units={"true_boom_torque": "N*m", "true_dipper_torque": "N*m", "true_bucket_torque": "N*m",
                 "true_boom_accel": "rad/s^2", "true_dipper_accel": "rad/s^2",
                 "true_bucket_accel": "rad/s^2", "true_slew_accel": "rad/s^2",
                 "true_slew_angle": "rad", "true_bucket_load": "kg"},
    truth_added=("true_bucket_load",),
    rate_pairs=(("boom_angle", "boom_rate", "rad/s", 0.02), ("dipper_angle", "dipper_rate", "rad/s", 0.02),
                ("bucket_angle", "bucket_rate", "rad/s", 0.02)),
)

#: Every sensor set by name.
SENSOR_SETS: dict[str, SensorSet] = {s.name: s for s in (THESIS_SENSORS, MACHINE_SENSORS)}


def get_sensor_set(sensor_set: "str | SensorSet") -> SensorSet:
    """The :class:`SensorSet` called ``sensor_set`` (an object is returned as it is).

    Parameters
    ----------
    sensor_set : str or SensorSet
        A registry name (``thesis``, ``machine``) or a sensor set.
    """
    if isinstance(sensor_set, SensorSet):
        return sensor_set
    try:
        return SENSOR_SETS[str(sensor_set)]
    except KeyError:
        from excavator_payload.errors import DatasetError

        raise DatasetError(f"unknown sensor set '{sensor_set}': choose one of "
                           f"{', '.join(SENSOR_SETS)}") from None


def detect_sensor_set(columns: Iterable[str]) -> SensorSet | None:
    """The sensor set whose signals are all among ``columns`` (the largest such), or None.

    Parameters
    ----------
    columns : iterable of str
        Column names of a table.
    """
    cols = set(columns)
    matches = [s for s in SENSOR_SETS.values() if set(s.signals) <= cols]
    return max(matches, key=lambda s: len(s.signals)) if matches else None
