"""The dataset schema: one row per 20 Hz sample, SI units, fixed column names.

Per-experiment metadata (seed, start and target pose, payload, machine, noise preset, solver
status) travels inside the Parquet file's schema metadata under the key
``excavator_payload`` as JSON (see :mod:`excavator_payload.data.io`).
"""

from __future__ import annotations

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
